"""What the evaluation's commands check in their arguments before anything runs: one error type,
one way to read ``KEY=VALUE`` lists, the question data, ``--env-arg`` and the results directory.

Each check fails with :class:`EvalError`, one line naming what is wrong and how to fix it; the
command prints it and exits 2, before any episode or question runs.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from ..protocol import EVAL_ENV_KWARGS, EVAL_SEED_BASE
from ..store import safe_name

# Fixed by the protocol (the evaluation split): not settable with --env-arg.
PROTOCOL_KEYS: tuple[str, ...] = tuple(EVAL_ENV_KWARGS)
PROTOCOL_TEXT = ", ".join(f"{k}={v}" for k, v in EVAL_ENV_KWARGS.items())  # "split=test, instructions=unseen"
SEEDS_TEXT = f"{EVAL_SEED_BASE:,} + i"  # the evaluation's seeds, as help texts write them
# Settings that change what an episode of a policy row means: a resumed run must keep them.
MANIFEST_KEYS = ("policy", "policy_kwargs", "obs_mode", "control_mode", "max_steps", "env_kwargs", "benchmark_version",
                 "checkpoint")
# Settings that change what a backbone row means: a resumed run must keep them.
BACKBONE_KEYS = ("backbone", "backbone_kwargs", "images", "env_kwargs")
RESULTS_ROOT = Path("results")  # --out defaults to results/<name>


class EvalError(RuntimeError):
    """Bad arguments or a results directory that does not fit this run."""


def parse_kv(items: list[str], what: str) -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}``: each VALUE parsed as JSON, else kept as a string."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise EvalError(f"{what} {item!r} must look like KEY=VALUE")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def check_env_args(env_kwargs: Mapping[str, Any], perturb_hint: str) -> None:
    """``--env-arg`` may set any gym.make keyword but those of the protocol and ``perturb`` (which
    ``perturb_hint`` says how to set, if the command can)."""
    fixed = [k for k in PROTOCOL_KEYS if k in env_kwargs]
    if fixed:
        raise EvalError(f"--env-arg cannot set {', '.join(fixed)}: the protocol fixes {PROTOCOL_TEXT}")
    if "perturb" in env_kwargs:
        raise EvalError(f"--env-arg cannot set perturb: {perturb_hint}")


def check_data(suites: list[str], data_dir: str | None) -> None:
    """Load each suite's evaluation pool now: missing GSM8K / MMLU-Pro fails before any episode runs."""
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic import EpisodeSampler
    from rsb_maniskill.semantic.errors import SemanticError

    for suite in suites:
        try:
            EpisodeSampler(split_env_id(suite)[0], data_dir=data_dir, **EVAL_ENV_KWARGS)
        except SemanticError as err:
            raise EvalError(f"{suite}: {err}") from err


def results_dir(out: str | None, label: str) -> Path:
    """The results directory, made and checked writable now: ``--out``, else ``results/<label>``
    (the label as a safe name)."""
    path = Path(out) if out else RESULTS_ROOT / safe_name(label)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".write-probe{os.getpid()}"
        probe.touch()
        probe.unlink()
    except OSError as err:
        raise EvalError(f"cannot write to results directory {path}: {err.strerror or err}; "
                        "choose another --out") from err
    return path
