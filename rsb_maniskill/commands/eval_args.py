"""What the evaluation's commands check in their arguments before anything runs: one error type,
one way to read ``KEY=VALUE`` lists, the question data, ``--env-arg``, the obs and control modes,
and the results directory.

Each check fails with :class:`EvalError`, one line naming what is wrong and how to fix it; the
command prints it and exits 2, before anything is written and before any episode or question runs.
The env's settings are checked against what its task class accepts (its keywords and their type
hints, its obs modes, its robot's controllers) without building an env.
"""
from __future__ import annotations

import argparse
import difflib
import inspect
import json
import types
import typing
import unicodedata
from pathlib import Path
from typing import Any, Mapping, Sequence

from rsb_maniskill.compat import CAMERA_TEXTURES, OBS_MODES, obs_mode_supported
from rsb_maniskill.evaluation.protocol import EVAL_ENV_KWARGS, EVAL_SEED_BASE
from rsb_maniskill.evaluation.store import folder_labels, folder_name
from rsb_maniskill.outdirs import writable_dir
from rsb_maniskill.parallel.plan import NO_RENDER_OBS_MODES
from rsb_maniskill.resolve import key_values

# Fixed by the protocol (the evaluation split): not settable with --env-arg.
PROTOCOL_KEYS: tuple[str, ...] = tuple(EVAL_ENV_KWARGS)
PROTOCOL_TEXT = ", ".join(f"{k}={v}" for k, v in EVAL_ENV_KWARGS.items())  # "split=test, instructions=unseen"
SEEDS_TEXT = f"{EVAL_SEED_BASE:,} + i"  # the evaluation's seeds, as help texts write them
# Settings that change what an episode of a policy row means: a resumed run must keep them.
MANIFEST_KEYS = ("policy", "policy_kwargs", "obs_mode", "control_mode", "max_steps", "env_kwargs", "benchmark_version",
                 "checkpoint")
# Settings that change what a backbone row means: a resumed run must keep them.
BACKBONE_KEYS = ("backbone", "backbone_kwargs", "images", "env_kwargs")
# Arguments of the remote policy / backbone that say how to reach the model, not what it is: a run resumes
# when its server comes back on another host or port, and the token is never written down.
TRANSPORT_ARGS = ("host", "port", "token", "connect_timeout", "request_timeout", "max_message_mb")
REMOTE = "remote"
RESULTS_ROOT = Path("results")  # --out defaults to results/<name>
# gym.make keywords that rsb eval sets from its own flags: an --env-arg would be ignored or fight them.
EVAL_FLAG_KEYS: dict[str, str] = {
    "obs_mode": "use -o / --obs-mode", "control_mode": "use -c / --control-mode", "num_envs": "use --num-envs",
    "sim_backend": "use -b / --sim-backend", "render_mode": "use --videos",
    "max_episode_steps": "use --max-steps",
}
JSON_EXAMPLES = {int: "3", float: "0.5", bool: "true", str: "text", tuple: "[224,224]", list: "[1,2]",
                 dict: '{"k":1}'}


class EvalError(RuntimeError):
    """Bad arguments or a results directory that does not fit this run."""


def run_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """A row's settings as run.json keeps them and its settings id digests them: the remote model's
    arguments without :data:`TRANSPORT_ARGS`. Also reads a row of an older run.json, which kept them
    (its run resumes on another port)."""
    out = dict(settings)
    for spec, kwargs in (("policy", "policy_kwargs"), ("backbone", "backbone_kwargs")):
        if out.get(spec) == REMOTE and isinstance(out.get(kwargs), Mapping):
            out[kwargs] = {k: v for k, v in out[kwargs].items() if k not in TRANSPORT_ARGS}
    return out


def parse_kv(items: list[str], what: str) -> dict[str, Any]:
    """``["a=1", "b=x"]`` -> ``{"a": 1, "b": "x"}`` (``resolve.key_values``), its error an EvalError."""
    try:
        return key_values(items, what)
    except ValueError as err:
        raise EvalError(str(err)) from None


def check_env_args(env_kwargs: Mapping[str, Any], perturb_hint: str,
                   flags: Mapping[str, str] = EVAL_FLAG_KEYS) -> None:
    """``--env-arg`` may set any gym.make keyword but those of the protocol, ``perturb`` (which
    ``perturb_hint`` says how to set, if the command can) and those the command's ``flags`` set."""
    fixed = [k for k in PROTOCOL_KEYS if k in env_kwargs]
    if fixed:
        raise EvalError(f"--env-arg cannot set {', '.join(fixed)}: the protocol fixes {PROTOCOL_TEXT}")
    if "perturb" in env_kwargs:
        raise EvalError(f"--env-arg cannot set perturb: {perturb_hint}")
    own = [k for k in env_kwargs if k in flags]
    if own:
        raise EvalError(f"--env-arg cannot set {own[0]}: {flags[own[0]]}")


def env_parameters(env_id: str) -> dict[str, Any]:
    """The keywords ``gym.make(env_id, ...)`` passes to the task class, each with its type hint
    (``Any`` when it has none): the task's own, then its bases' while each passes ``**kwargs`` on."""
    params: dict[str, Any] = {}
    for klass in _task_class(env_id).__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        signature = inspect.signature(init)
        try:
            hints = typing.get_type_hints(init)
        except Exception:  # noqa: BLE001  (a hint that does not resolve: the value is not checked)
            hints = {}
        for name, p in signature.parameters.items():
            if name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                params.setdefault(name, hints.get(name, Any))
        if not any(p.kind == p.VAR_KEYWORD for p in signature.parameters.values()):
            break  # it passes nothing further up
    return params


def _fits(value: Any, hint: Any) -> bool:
    """Whether a JSON value fits a type hint; hints of other classes (e.g. SimConfig) are left to the env."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, h) for h in args)
    if hint is type(None):
        return value is None
    if hint in (int, float, bool) and isinstance(value, bool) != (hint is bool):
        return False
    if hint in (int, bool, str, dict):
        return isinstance(value, hint)
    if hint is float:
        return isinstance(value, (int, float))
    if origin is dict:
        return isinstance(value, dict)
    if origin in (tuple, list) or hint in (tuple, list):
        if not isinstance(value, (list, tuple)):
            return False
        if origin is tuple and args and args[-1] is not Ellipsis:
            return len(value) == len(args) and all(_fits(v, a) for v, a in zip(value, args))
        return not args or all(_fits(v, args[0]) for v in value)
    return True


def _example(hint: Any) -> str:
    """A JSON example of a value of ``hint`` (its first non-None form)."""
    forms = [h for h in (typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType)
                         else (hint,)) if h is not type(None)]
    first = forms[0] if forms else hint
    return JSON_EXAMPLES.get(typing.get_origin(first) or first, "...")


def _hint_text(hint: Any) -> str:
    return getattr(hint, "__name__", None) if isinstance(hint, type) else str(hint).replace("typing.", "")


def check_env_settings(suites: Sequence[str], env_kwargs: Mapping[str, Any], obs_mode: str | None = None,
                       control_mode: str | None = None) -> None:
    """``--env-arg`` keywords and values, the obs mode and the control mode, against what the
    suites' task classes accept (no env is built): a keyword they do not take, a value of another
    type than the keyword's hint, a keyword the suite id fixes (``targets``), an obs mode ManiSkill
    does not know, a controller the robot does not have."""
    from rsb_maniskill.env_ids import ENVS

    by_suite = {k for _, kwargs in ENVS.values() for k in kwargs}  # suite_id, targets
    for suite in dict.fromkeys(suites):
        params = env_parameters(suite) if env_kwargs else {}  # no keyword to check: the simulator stays unloaded
        for key, value in env_kwargs.items():
            if key in by_suite:
                raise EvalError(f"--env-arg cannot set {key}: the suite id fixes it (e.g. RSB-Math-4-Objects for "
                                "everyday objects)")
            if key not in params:
                named = [k for k in params if k not in (*PROTOCOL_KEYS, *EVAL_FLAG_KEYS, *by_suite, "perturb")]
                raise EvalError(f"--env-arg {key}: {suite} takes no keyword {key!r}; it takes {', '.join(named)}")
            if not _fits(value, params[key]):
                raise EvalError(f"--env-arg {key}={json.dumps(value)}: {key} takes {_hint_text(params[key])}; VALUE "
                                f"is read as JSON, e.g. -e {key}={_example(params[key])}")
        if obs_mode is not None:
            _check_obs_mode(suite, obs_mode)
        if control_mode is not None:
            default = inspect.signature(_task_class(suite)).parameters.get("robot_uids")
            robot = env_kwargs.get("robot_uids", default.default if default is not None else None)
            modes = _control_modes(robot)
            if modes and control_mode not in modes:
                raise EvalError(f"-c {control_mode}: not a controller of the robot {robot}; use one of "
                                f"{', '.join(modes)}")


def _task_class(env_id: str) -> type:
    """The task class ``gym.make(env_id)`` builds (importing the simulator's modules, building nothing)."""
    from rsb_maniskill.registration import served_by
    from rsb_maniskill.tasks import TASK_CLASSES

    return served_by(TASK_CLASSES)[env_id]


def _check_obs_mode(suite: str, obs_mode: str) -> None:
    """ManiSkill's rule on the task class's own obs modes (``-o`` was checked against ManiSkill's
    when it was parsed: :class:`ObsModeAction`)."""
    if obs_mode in NO_RENDER_OBS_MODES:  # every ManiSkill task's: no need to load the simulator to say so
        return
    problem = obs_mode_problem(obs_mode, _task_class(suite).SUPPORTED_OBS_MODES)
    if problem:
        raise EvalError(f"-o {obs_mode}: {problem}")


def obs_mode_problem(obs_mode: str, supported: Sequence[str] = OBS_MODES) -> str | None:
    """Why ``obs_mode`` is no obs mode of an env supporting ``supported`` (None when it is one), with
    the modes to use; a word near none of them is taken for the results folder -o once named."""
    if obs_mode_supported(obs_mode, supported):
        return None
    named = [m for m in supported if m != "any_textures"]
    textures = f", or camera textures ({', '.join(CAMERA_TEXTURES)}) joined by '+'" if "any_textures" in supported \
        else ""
    words = [*named, *CAMERA_TEXTURES]
    parts = obs_mode.split("+")
    near = ["".join(difflib.get_close_matches(t, words, n=1)) if t not in words else t for t in parts]
    then = ""
    if obs_mode.strip() and ("/" in obs_mode or Path(obs_mode).exists() or near == [""]):
        # "-o results/pi0": -o named the results folder before it named the obs mode
        then = f"; -o is the obs mode: the results folder is --out {obs_mode}"
    elif all(near):
        then = f" (did you mean {'+'.join(near)}?)"
    return f"not an obs mode; use one of {', '.join(named)}{textures}, e.g. rgb or rgb+depth{then}"


class ObsModeAction(argparse.Action):
    """``-o``, refused as it is parsed when ManiSkill has no such obs mode: in a second, before the
    simulator loads (the task class's own modes are checked with the other settings)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        problem = obs_mode_problem(values)
        if problem:
            parser.error(f"{option_string} {values}: {problem}")
        setattr(namespace, self.dest, values)


def name_problem(name: str) -> str | None:
    """Why ``name`` cannot be a row label (None when it can): a control character (a newline, a tab)
    or a line separator would break every table row it stands in."""
    for i, ch in enumerate(name):
        if unicodedata.category(ch) in ("Cc", "Zl", "Zp"):
            return (f"holds a control character ({ch!r} at position {i}): it would break the rows of the tables; "
                    "give a name on one line, without tabs")
    return None


class NameAction(argparse.Action):
    """``--name``, refused as it is parsed when it cannot be a row label (:func:`name_problem`)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        problem = name_problem(values)
        if problem:
            parser.error(f"{option_string} {values!r}: {problem}")
        setattr(namespace, self.dest, values)


def _control_modes(robot: Any) -> list[str]:
    """The controllers of a registered robot: the keys of its agent's ``_controller_configs``, read
    on an instance built without a scene (the property needs only the joint names); empty when they
    cannot be read so (the env then tells)."""
    from mani_skill.agents.registration import REGISTERED_AGENTS

    import rsb_maniskill.agents  # noqa: F401  (registers the robot)

    spec = REGISTERED_AGENTS.get(robot) if isinstance(robot, str) else None
    if spec is None:
        return []
    try:
        return list(spec.agent_cls._controller_configs.fget(object.__new__(spec.agent_cls)))
    except Exception:  # noqa: BLE001  (an agent whose controllers need its scene)
        return []


def check_data(suites: list[str], data_dir: str | None, color_map: str | None = None) -> None:
    """Load each suite's evaluation pool now (with ``-e color_map``, when given): missing GSM8K /
    MMLU-Pro, or an unknown colour map, fails before any episode runs."""
    from rsb_maniskill.objects.family import split_env_id
    from rsb_maniskill.semantic import EpisodeSampler
    from rsb_maniskill.semantic.errors import SemanticError

    for suite in suites:
        try:
            EpisodeSampler(split_env_id(suite)[0], data_dir=data_dir, **EVAL_ENV_KWARGS,
                           **({"color_map": color_map} if color_map is not None else {}))
        except (SemanticError, ValueError) as err:
            raise EvalError(f"{suite}: {err}") from err


def results_dir(out: str | None, label: str) -> Path:
    """The results directory, made and checked writable now: ``--out``, else ``results/<label>``
    (the label as a folder name, one way: ``store.folder_name``)."""
    try:  # the name is checked with --out too: the row's chart and videos are named by it
        path = RESULTS_ROOT / folder_name(label) if not out else Path(out)
        folder_name(label)
    except ValueError as err:
        raise EvalError(str(err)) from None
    if not out:  # a folder of one name: another whose folder name is the same ("a:b", "a/b") is refused
        owners = folder_labels(path)
        others = [name for name in owners if name != label]
        if others and label not in owners:
            raise EvalError(f"{path} holds the runs of {others[0]!r}, whose name makes the same folder name as "
                            f"{label!r}; give this run its own --out (or another --name)")
    try:
        if path.exists() and not path.is_dir():
            raise EvalError(f"results directory {path} is a file, not a directory; choose another --out")
        writable_dir(path)
    except OSError as err:
        raise EvalError(f"cannot write to results directory {path}: {err.strerror or err}; "
                        "choose another --out") from err
    return path


def check_policy_args(spec: str, policy_kwargs: Mapping[str, Any]) -> None:
    """``-a`` against the arguments of the policy's factory (``remote``: its protocol's options, checked
    with the server)."""
    from rsb_maniskill.policies.registry import check_factory_args

    if spec == "remote":
        return
    try:
        check_factory_args(spec, policy_kwargs)
    except TypeError as err:
        raise EvalError(f"{err}; give the factory's arguments with -a KEY=VALUE") from None
