"""The policy interface of the evaluator, the table of built-in policies, and loading a policy
from a built-in name or ``module:factory``.

A policy is anything with ``reset(instruction, obs)`` and ``act(obs) -> (T, action_dim)`` chunk.
The runner calls ``reset`` once per episode with the instruction (after the instruction-mode
ablation) and the first observation, then ``act``; it executes the T actions of the chunk in
order and calls ``act`` again with the newest observation. Observations are the single-env
observation as numpy arrays in the env's nested dict layout (leading env dim removed).

A policy that talks returns ``{"actions": chunk, "text": str}`` instead of the bare chunk (its
chain of thought, say): the record keeps the episode's text and the option it states
(``statements.py``). The batched form's mapping holds one text per env (None where it has none).

The optional batched form (:class:`BatchedPolicy`) drives the B parallel envs of ``--num-envs``
with one object: ``reset_batch(instructions, obs)`` and ``act_batch(obs, envs) -> (len(envs), T,
action_dim)``, observations keeping their leading env dim. A policy that has it (the remote
client: one request per step for all envs) is built once; one without it is built once per env
and batched by :class:`PerEnvPolicies`. The single-env form is what everything else uses.

A policy that misbehaves (raises in ``reset`` / ``act``, or returns what the env cannot take)
raises :class:`~rsb_maniskill.evaluation.policy_error.PolicyError`: one line naming the policy,
the episode and what came back, its traceback kept for ``rsb --debug``.
"""
from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from rsb_maniskill.evaluation.policy_error import PolicyError, shown


@runtime_checkable
class Policy(Protocol):
    """What ``rsb eval`` needs from a policy. An optional ``name`` attribute labels its records."""

    def reset(self, instruction: str, obs: dict) -> None:
        """Start an episode: ``instruction`` is the text the policy may use ("" in blank mode)."""

    def act(self, obs: dict) -> Any:
        """Action chunk of shape (T, action_dim), T >= 1, executed in order before the next call;
        or ``{"actions": chunk, "text": str}``."""


@runtime_checkable
class BatchedPolicy(Protocol):
    """The optional batched form: one object for B parallel envs (rows of batched observations)."""

    def reset_batch(self, instructions: Sequence[str], obs: dict) -> None:
        """Start B episodes: env i gets ``instructions[i]``; ``obs`` rows are the envs' first observations."""

    def act_batch(self, obs: dict, envs: Sequence[int]) -> Any:
        """Chunks for the envs ``envs`` (indices into the reset's B), ``obs`` holding their rows in that
        order: a (len(envs), T, action_dim) array, or a list of (T_i, action_dim) chunks; or
        ``{"actions": chunks, "text": [one str or None per env]}``."""


def is_batched(policy: Any) -> bool:
    return callable(getattr(policy, "reset_batch", None)) and callable(getattr(policy, "act_batch", None))


def obs_rows(obs: Any, rows: Sequence[int]) -> Any:
    """Rows ``rows`` of a batched (nested) observation, as numpy with the leading dim kept."""
    if isinstance(obs, dict):
        return {k: obs_rows(v, rows) for k, v in obs.items()}
    if hasattr(obs, "detach"):
        obs = obs.detach().cpu().numpy()
    return np.asarray(obs)[list(rows)]


class PerEnvPolicies:
    """The batched form over one single-env policy per env (``--num-envs`` for a policy without it)."""

    def __init__(self, policies: Sequence[Any]) -> None:
        self.policies = list(policies)
        self.name = policy_name(self.policies[0]) if self.policies else "policy"

    def reset_batch(self, instructions: Sequence[str], obs: dict) -> None:
        if len(instructions) > len(self.policies):
            raise ValueError(f"need one policy per env: {len(instructions)} envs, {len(self.policies)} policies")
        for i, text in enumerate(instructions):
            self.policies[i].reset(text, _row(obs, i))

    def act_batch(self, obs: dict, envs: Sequence[int]) -> Any:
        return join_outputs([self.policies[e].act(_row(obs, k)) for k, e in enumerate(envs)])


def _row(obs: Any, i: int) -> Any:
    if isinstance(obs, dict):
        return {k: _row(v, i) for k, v in obs.items()}
    return np.asarray(obs)[i]


def as_chunks(actions: Any, n: int, action_dim: int | None = None) -> list[np.ndarray]:
    """Check a batched policy's output: ``n`` chunks, each as :func:`as_chunk` wants it."""
    if isinstance(actions, np.ndarray) and actions.ndim != 3:
        raise PolicyError(f"act_batch must return shape (envs, T, action_dim), got shape {actions.shape}")
    if isinstance(actions, (str, bytes)) or not isinstance(actions, (np.ndarray, Sequence)):
        raise PolicyError(f"act_batch returned {shown(actions)}; return an array of shape (envs, T, action_dim) "
                          "or a list of (T, action_dim) chunks")
    chunks = list(actions)
    if len(chunks) != n:
        raise PolicyError(f"act_batch returned {len(chunks)} chunks for {n} envs")
    return [as_chunk(c, action_dim, "act_batch") for c in chunks]


def _actions(out: Mapping, method: str) -> Any:
    if "actions" not in out:
        raise PolicyError(f"{method} returned a mapping without 'actions' (keys: {sorted(map(str, out))}); "
                          "return the actions, or {'actions': ..., 'text': ...}")
    return out["actions"]


def split_output(out: Any) -> tuple[Any, str | None]:
    """A policy's ``act`` output as (actions, text): the bare actions give no text (None)."""
    if not isinstance(out, Mapping):
        return out, None
    text = out.get("text")
    if text is not None and not isinstance(text, str):
        raise PolicyError(f"act returned 'text' of type {type(text).__name__}; it must be a str")
    return _actions(out, "act"), text


def split_outputs(out: Any, n: int) -> tuple[Any, list[str | None]]:
    """A batched policy's output as (actions, one text or None per env)."""
    if not isinstance(out, Mapping):
        return out, [None] * n
    texts = out.get("text")
    if texts is None:
        return _actions(out, "act_batch"), [None] * n
    if isinstance(texts, str) or not isinstance(texts, Sequence) or len(texts) != n \
            or not all(t is None or isinstance(t, str) for t in texts):
        raise PolicyError(f"act_batch must return 'text' as a list of {n} str (or None), one per env; "
                          f"got {type(texts).__name__}")
    return _actions(out, "act_batch"), list(texts)


def join_outputs(outs: Sequence[Any]) -> Any:
    """Single-env outputs of several envs as one batched output (a mapping when any has text)."""
    pairs = [split_output(o) for o in outs]
    if all(text is None for _, text in pairs):
        return [a for a, _ in pairs]
    return {"actions": [a for a, _ in pairs], "text": [t for _, t in pairs]}


def env_action_space(env: Any) -> Any:
    """The action space of one env of ``env`` (ManiSkill's ``single_action_space`` when batched)."""
    return getattr(env.unwrapped, "single_action_space", None) or env.action_space


def policy_name(policy: Any) -> str:
    """Label for records and tables: the policy's ``name`` attribute, else its class name."""
    name = getattr(policy, "name", None)
    return str(name) if name else type(policy).__name__


def as_chunk(actions: Any, action_dim: int | None = None, method: str = "act") -> np.ndarray:
    """Check and normalise a policy's output to a float (T, action_dim) array.

    A single action of shape (action_dim,) is accepted as a chunk of one. Errors (PolicyError) say
    what came back, since a wrong output from a user policy is the most common integration bug.
    """
    want = f"an array of shape (T, {action_dim or 'action_dim'}) with T >= 1"
    if actions is None:
        raise PolicyError(f"{method} returned None; return {want}")
    if isinstance(actions, np.ndarray):
        a = actions
    else:
        try:
            a = np.asarray(actions, dtype=np.float64)
        except (TypeError, ValueError):
            raise PolicyError(f"{method} returned {shown(actions)}, not numbers; return {want}") from None
    if a.ndim == 1:
        a = a[None]
    if a.ndim == 2 and a.shape[0] == 0:
        raise PolicyError(f"{method} returned an empty chunk (shape {a.shape}); return {want}")
    if a.ndim != 2:
        raise PolicyError(f"{method} must return {want}, got shape {a.shape}")
    if action_dim is not None and a.shape[1] != action_dim:
        raise PolicyError(f"{method} returned actions of dim {a.shape[1]} (chunk shape {a.shape}); the env takes "
                          f"{action_dim} numbers an action (its control mode's action space)")
    if not np.issubdtype(a.dtype, np.number):
        raise PolicyError(f"{method} returned an array of dtype {a.dtype}; return {want} of numbers")
    bad = ~np.isfinite(a)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise PolicyError(f"{method} returned NaN or inf actions ({int(bad.sum())} of {a.size} numbers, the first "
                          f"at action {row}, index {col}: {a[row, col]})")
    return a


class RandomPolicy:
    """Uniform random actions in [low, high]: the floor of the benchmark (no grasp expected)."""

    name = "random"

    def __init__(self, low: Any, high: Any, chunk_size: int = 1, seed: int = 0) -> None:
        self.low = np.asarray(low, dtype=np.float32)
        self.high = np.asarray(high, dtype=np.float32)
        if self.low.shape != self.high.shape or self.low.ndim != 1:
            raise ValueError(f"low and high must be 1-D of equal shape, got {self.low.shape} and {self.high.shape}")
        self.chunk_size = int(chunk_size)
        self.rng = np.random.default_rng(seed)

    @classmethod
    def from_action_space(cls, space: Any, **kwargs: Any) -> "RandomPolicy":
        """From a gymnasium Box (batched spaces: the last axis is the action)."""
        low, high = np.asarray(space.low), np.asarray(space.high)
        return cls(low.reshape(-1, low.shape[-1])[0], high.reshape(-1, high.shape[-1])[0], **kwargs)

    @classmethod
    def for_env(cls, env: Any, chunk_size: int = 1, seed: int = 0) -> "RandomPolicy":
        """Over the action space of one env of ``env`` (the ``random`` policy's factory)."""
        return cls.from_action_space(env_action_space(env), chunk_size=chunk_size, seed=seed)

    def reset(self, instruction: str, obs: dict) -> None:
        pass

    def act(self, obs: dict) -> np.ndarray:
        return self.rng.uniform(self.low, self.high, size=(self.chunk_size, self.low.shape[0])).astype(np.float32)


@dataclass(frozen=True)
class PolicySpec:
    """A built-in policy: where its factory lives, and what building and running it takes.

    ``factory`` is ``"package.module:attr"`` (imported on first use, so naming a policy imports
    nothing) or a callable. A factory that ``needs_env`` is called as ``factory(env, **kwargs)``.
    """

    factory: str | Callable[..., Any]
    needs_env: bool = False
    single_env: bool = False  # reads the simulator of env 0: one env at a time, never parallel envs
    obs_mode: str = "rgb"  # the observations it reads by default


# The one table of built-in names. Privileged baselines are built with the env and drive one env;
# policies that ignore observations get state obs (and so no renderer) by default.
POLICIES: dict[str, PolicySpec] = {
    "oracle": PolicySpec("rsb_maniskill.evaluation.reference_policies:oracle", needs_env=True, single_env=True,
                         obs_mode="state"),
    "blind": PolicySpec("rsb_maniskill.evaluation.reference_policies:blind", needs_env=True, single_env=True,
                        obs_mode="state"),
    "leftmost": PolicySpec("rsb_maniskill.evaluation.reference_policies:leftmost", needs_env=True,
                           single_env=True, obs_mode="state"),
    "random": PolicySpec("rsb_maniskill.evaluation.policy:RandomPolicy.for_env", needs_env=True, obs_mode="state"),
    # openpi (default) or vla-eval (-a protocol=vla-eval); needs the `eval` / `vla_eval` extra
    "remote": PolicySpec("rsb_maniskill.evaluation.remote:remote_policy"),
}
_USER_SPEC = PolicySpec("")  # what a "package.module:factory" spec is: no env, rgb observations


def register_policy(name: str, factory: str | Callable[..., Any], *, needs_env: bool = False,
                    single_env: bool = False, obs_mode: str = "rgb") -> None:
    """Make ``load_policy(name)`` use ``factory``; names hold no ':' so they never clash with specs."""
    if ":" in name:
        raise ValueError(f"built-in policy names cannot contain ':', got {name!r}")
    POLICIES[name] = PolicySpec(factory, needs_env, single_env, obs_mode)


def builtin_policies() -> tuple[str, ...]:
    return tuple(sorted(POLICIES))


def policy_spec(spec: str) -> PolicySpec:
    """The table entry of a built-in name; user specs get the defaults (no env, rgb)."""
    return POLICIES.get(spec, _USER_SPEC)


def resolve_factory(spec: str) -> Callable[..., Any]:
    """The factory a built-in name or ``"package.module:factory"`` names, without calling it.

    Errors name the part of the spec that failed (no ':', a module that does not import, a
    missing or non-callable attribute)."""
    if not isinstance(spec, str) or not spec:
        raise ValueError(f"policy spec must be a non-empty string, got {spec!r}")
    if spec in POLICIES:
        factory = POLICIES[spec].factory
        return factory if callable(factory) else import_factory(factory)
    if ":" not in spec:
        raise ValueError(
            f"policy {spec!r} is neither a built-in ({', '.join(builtin_policies())}) nor of the form "
            "'package.module:factory'"
        )
    return import_factory(spec)


def import_factory(spec: str, what: str = "policy") -> Callable[..., Any]:
    """The callable ``"package.module:attr"`` names (``attr`` may be dotted); errors name the part
    of the spec that failed and call it a ``what`` spec."""
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise ValueError(f"{what} spec {spec!r} must be 'package.module:factory' with both parts non-empty")
    try:
        factory = importlib.import_module(module_name)
    except ImportError as err:
        raise ImportError(f"{what} spec {spec!r}: cannot import module {module_name!r}: {err}") from err
    for part in attr.split("."):
        try:
            factory = getattr(factory, part)
        except AttributeError:
            raise AttributeError(f"{what} spec {spec!r}: module {module_name!r} has no attribute {attr!r}") from None
    if not callable(factory):
        raise TypeError(f"{what} spec {spec!r}: {attr!r} is not callable")
    return factory


def check_factory_args(spec: str, kwargs: Mapping[str, Any]) -> None:
    """Before anything runs: TypeError (one line, naming the factory's arguments) when the factory
    of ``spec`` cannot take ``kwargs``: an argument it does not have, or a required one missing.
    A factory taking ``**kwargs`` passes on what it is given, so it passes here too."""
    factory = resolve_factory(spec)
    try:
        signature = inspect.signature(factory)
    except (TypeError, ValueError):  # not introspectable (a C function): it will tell when called
        return
    given_env = (None,) if policy_spec(spec).needs_env else ()
    try:
        signature.bind(*given_env, **kwargs)
    except TypeError as err:
        names = [name for name, p in list(signature.parameters.items())[len(given_env):]
                 if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        raise TypeError(f"policy {spec!r}: {err} (its arguments: {', '.join(names) or 'none'})") from None


def load_policy(spec: str, *, env: Any = None, check: bool = True, **kwargs: Any) -> Policy:
    """Build a policy from a built-in name or ``"package.module:factory"`` and ``kwargs``.

    ``factory`` is any callable (a class or a function) returning an object with ``reset`` and
    ``act`` (checked unless ``check=False``). Built-ins that need the env (``oracle``, ``blind``,
    ``random``) get ``env``; user policies never see it. Errors name the part of the spec that failed.
    """
    entry = policy_spec(spec)
    factory = resolve_factory(spec)
    if entry.needs_env:
        if env is None:
            raise ValueError(f"policy {spec!r} is built with the env: pass env=...")
        if entry.single_env and getattr(env.unwrapped, "num_envs", 1) != 1:
            raise ValueError(f"policy {spec!r} drives one env at a time; use num_procs instead of num_envs")
        policy = factory(env, **kwargs)
    else:
        policy = factory(**kwargs)
    if not check:
        return policy
    missing = [m for m in ("reset", "act") if not callable(getattr(policy, m, None))]
    if missing:
        raise TypeError(
            f"policy spec {spec!r}: the factory returned {type(policy).__name__}, which lacks {' and '.join(missing)}()"
        )
    return policy
