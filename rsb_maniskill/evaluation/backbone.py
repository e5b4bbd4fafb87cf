"""Backbones: ask a policy's backbone the protocol's questions, exactly as the policy gets them.

The library of ``rsb backbone`` (the command is ``commands/backbone.py``):

    rsb backbone arithmetic --suites RSB-Math-4 RSB-Math-10 --out results/blind
    rsb backbone my_models:make_backbone -a path=ckpt --suites paper --images --out results/pi05
    rsb backbone remote -a host=gpu-box -a port=8001 --name qwen3-4b --out results/pi05

A backbone is anything with ``answer(instruction, images) -> str``: ``instruction`` is the text
the policy is given (after the ``--instruction`` ablation, with the same shuffled donors as ``rsb
eval``), ``images`` the head-camera frame of the episode's first observation (``{"head": (H, W, 3)
uint8}``, with ``--images``; else ``{}``). Its answer is parsed by the parser that reads a talking
policy's text (``semantic.answers``), so "option B", "the green block" and "10" count alike.

Each episode's record goes to ``<out>/backbone.jsonl`` beside an eval run's ``episodes.jsonl``
(rerunning resumes); ``rsb report`` then sets the backbone's accuracy beside the policy's TSR and
nSG on the same episodes (``reporting/sections/gap.py``). Built in, as reference lines:

- ``arithmetic`` solves RSB-Math exactly from the question's text and says nothing elsewhere: the
  upper line of a backbone on Math;
- ``similarity`` is the audit's question-aware reader (``rsb audit``; the backbone lives beside it in
  ``audit/readers.py``): the option whose sentence embedding is nearest the question's, read from
  the instruction: the shallow line;
- ``remote`` asks a backbone served over the websocket protocol of ``remote/`` (``RemoteBackbone``).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

IMAGE_CAMERA = "head"  # the camera whose first frame --images sends


@runtime_checkable
class Backbone(Protocol):
    """What ``rsb backbone`` needs; an optional ``name`` labels its records."""

    def answer(self, instruction: str, images: Mapping[str, np.ndarray]) -> str:
        """The backbone's reply, in words ("B", "option B", "The answer is 10.", a chain of thought)."""


class ArithmeticBackbone:
    """Solves the RSB-Math question in the instruction exactly ("27 minus 17 equals 10."); says
    nothing ("") when the instruction holds none (other suites, a blank instruction)."""

    name = "arithmetic"

    def answer(self, instruction: str, images: Mapping[str, np.ndarray]) -> str:
        from rsb_maniskill.semantic.math_source import solve

        solved = solve(instruction)
        if solved is None:
            return ""
        a, op, b, value = solved
        return f"{a} {op} {b} equals {value}."


# Built-in backbones; a "package.module:factory" spec names any other.
BACKBONES: dict[str, str] = {
    "arithmetic": "rsb_maniskill.evaluation.backbone:ArithmeticBackbone",
    "similarity": "rsb_maniskill.audit.readers:SimilarityBackbone",
    "remote": "rsb_maniskill.policies.remote.client:RemoteBackbone",
}


def resolve_backbone(spec: str) -> Callable[..., Any]:
    """The factory a built-in name or ``package.module:factory`` names, without calling it."""
    from rsb_maniskill.resolve import resolve

    if spec in BACKBONES:
        return resolve(BACKBONES[spec], "backbone")
    if ":" not in spec:
        raise ValueError(f"backbone {spec!r} is neither a built-in ({', '.join(BACKBONES)}) nor of the form "
                         "'package.module:factory'")
    return resolve(spec, "backbone")


def load_backbone(spec: str, **kwargs: Any) -> Backbone:
    """Build a backbone from a built-in name or ``package.module:factory`` and ``kwargs``."""
    backbone = resolve_backbone(spec)(**kwargs)
    if not callable(getattr(backbone, "answer", None)):
        raise TypeError(f"backbone spec {spec!r}: the factory returned {type(backbone).__name__}, which lacks answer()")
    return backbone


# ---------------------------------------------------------------- asking
class _Questions:
    """The protocol's episodes of one suite as a policy meets them: the spec of each seed, and with
    ``images`` the head camera's first frame (from a reset of the evaluation env)."""

    def __init__(self, suite_id: str, env_kwargs: Mapping[str, Any], images: bool) -> None:
        from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS
        from rsb_maniskill.objects.family import split_env_id
        from rsb_maniskill.semantic import EpisodeSampler

        base, targets = split_env_id(suite_id)
        sampler_keys = ("data_dir", "color_map")
        self.sampler = EpisodeSampler(base, targets=targets, **EVAL_ENV_KWARGS,
                                      **{k: v for k, v in env_kwargs.items() if k in sampler_keys})
        self.env = None
        if images:
            import gymnasium as gym

            import rsb_maniskill  # noqa: F401  (registers the RSB-* envs)

            self.env = gym.make(suite_id, obs_mode="rgb", **{**EVAL_ENV_KWARGS, **env_kwargs})

    def __call__(self, seed: int) -> tuple[Any, dict[str, np.ndarray]]:
        if self.env is None:
            return self.sampler.episode(seed), {}
        from rsb_maniskill.batch import single_env_obs
        from rsb_maniskill.robot import sensor_uid

        obs, _ = self.env.reset(seed=seed)
        frame = single_env_obs(obs)["sensor_data"][sensor_uid(IMAGE_CAMERA)]["rgb"]
        return self.env.unwrapped.episode_specs[0], {IMAGE_CAMERA: np.asarray(frame)}

    def close(self) -> None:
        if self.env is not None:
            self.env.close()


def _answer_text(answer: Any) -> str:
    """A backbone's reply as text: None is no answer; anything but a str is a mistake to report."""
    if answer is None:
        return ""
    if not isinstance(answer, str):
        raise TypeError(f"backbone.answer must return a str, got {type(answer).__name__}")
    return answer


def ask_episodes(backbone: Backbone, suite_id: str, seeds: Sequence[int], out_path: str | Path, *,
                 label: str, instruction_mode: str = "normal", images: bool = False,
                 env_kwargs: Mapping[str, Any] | None = None, progress: bool = True) -> list[dict]:
    """Ask ``backbone`` the episodes ``seeds`` of ``suite_id`` (those not yet in ``out_path``),
    appending one record each; returns every record of this row and suite, old and new."""
    from rsb_maniskill.evaluation.protocol import SHUFFLE_SEED, ShuffledDonors, ablate
    from rsb_maniskill.evaluation.statements import EpisodeText
    from rsb_maniskill.evaluation.store import RecordWriter, read_backbone_records

    seeds = [int(s) for s in seeds]
    mine = [r for r in read_backbone_records(out_path)
            if (r["backbone"], r["suite_id"], r["instruction_mode"]) == (label, suite_id, instruction_mode)]
    done = {int(r["seed"]) for r in mine}
    todo = [s for s in seeds if s not in done]
    if not todo:
        return mine
    questions = _Questions(suite_id, dict(env_kwargs or {}), images)
    donors = (ShuffledDonors(seeds, lambda s: questions.sampler.episode(s).instruction, SHUFFLE_SEED)
              if instruction_mode == "shuffled" else None)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(seeds), initial=len(done), desc=f"{label} {suite_id} [{instruction_mode}]", unit="q")
    try:
        with RecordWriter(out_path, validate=False) as writer:
            for seed in todo:
                t0 = time.monotonic()
                spec, frames = questions(seed)
                donor = donors(seed, spec.instruction) if donors is not None else None
                given, extra = ablate(spec.instruction, instruction_mode, donor)
                said = EpisodeText()
                said.add(_answer_text(backbone.answer(given, frames)))
                fields = said.fields(spec)
                record = {"backbone": label, "suite_id": suite_id, "seed": seed, "question_id": int(spec.question_id),
                          "instruction_mode": instruction_mode, "instruction": given,
                          "correct_letter": spec.correct_letter, **fields,
                          "correct": fields["stated_letter"] == spec.correct_letter, "images": bool(images),
                          **extra, "wall_s": round(time.monotonic() - t0, 3)}
                mine.append(writer.write(record))
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(acc=f"{sum(r['correct'] for r in mine) / len(mine):.0%}", refresh=False)
    finally:
        questions.close()
        if bar is not None:
            bar.close()
    return mine
