"""The table of built-in policies and loading a policy from a built-in name or ``module:factory``.

A built-in is one :class:`PolicySpec` row (or a :func:`register_policy` call from anywhere): its
factory is named, not imported, so naming a policy imports nothing until it is used.
"""
from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from rsb_maniskill.policies.interface import Policy
from rsb_maniskill.resolve import resolve


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
    heavy: bool = False  # loads a model (a checkpoint): worth loading once for every worker where that pays
    gpu: bool = False  # its model computes on a GPU where there is one: `--policy-process auto` then serves it once


# The one table of built-in names. Privileged baselines are built with the env and drive one env;
# policies that ignore observations get state obs (and so no renderer) by default.
POLICIES: dict[str, PolicySpec] = {
    "oracle": PolicySpec("rsb_maniskill.policies.reference:oracle", needs_env=True, single_env=True,
                         obs_mode="state"),
    "blind": PolicySpec("rsb_maniskill.policies.reference:blind", needs_env=True, single_env=True,
                        obs_mode="state"),
    "leftmost": PolicySpec("rsb_maniskill.policies.reference:leftmost", needs_env=True,
                           single_env=True, obs_mode="state"),
    "random": PolicySpec("rsb_maniskill.policies.reference:RandomPolicy.for_env", needs_env=True, obs_mode="state"),
    # openpi (default) or vla-eval (-a protocol=vla-eval); needs the `eval` / `vla_eval` extra
    "remote": PolicySpec("rsb_maniskill.policies.remote:remote_policy"),
}
_USER_SPEC = PolicySpec("")  # what a "package.module:factory" spec is: no env, rgb observations


def register_policy(name: str, factory: str | Callable[..., Any], *, needs_env: bool = False,
                    single_env: bool = False, obs_mode: str = "rgb", heavy: bool = False, gpu: bool = False) -> None:
    """Make ``load_policy(name)`` use ``factory``; names hold no ':' so they never clash with specs.

    A name taken already is refused (ValueError): a plugin cannot replace ``oracle`` and have a
    resume pool its episodes with the real oracle's."""
    if ":" in name:
        raise ValueError(f"built-in policy names cannot contain ':', got {name!r}")
    if name in POLICIES:
        raise ValueError(f"policy name {name!r} is taken (by {factory_path(name)}); register the policy under "
                         "another name")
    POLICIES[name] = PolicySpec(factory, needs_env, single_env, obs_mode, heavy, gpu)


def is_heavy(spec: str) -> bool:
    """Whether a policy declares that it loads a model worth loading once for every worker: its
    table entry's ``heavy``, or for ``package.module:factory`` the factory's own ``heavy = True``
    attribute (imports the factory's module)."""
    if spec in POLICIES:
        return POLICIES[spec].heavy
    return bool(getattr(resolve_factory(spec), "heavy", False))


def runs_on_gpu(spec: str) -> bool:
    """Whether a policy declares that its model computes on a GPU where one is there (``gpu``, as
    ``heavy``): one served model batches every worker's envs in a forward pass that costs about the
    same for 1 and 32 rows there; on the CPU a copy a worker was faster (``benchmarks/policy_server.py``)."""
    if spec in POLICIES:
        return POLICIES[spec].gpu
    return bool(getattr(resolve_factory(spec), "gpu", False))


def factory_path(spec: str) -> str:
    """Where the code of ``spec`` lives, as ``"package.module:attr"`` (a built-in's factory, or the spec
    itself): what a resume checks its records came from."""
    factory = POLICIES[spec].factory if spec in POLICIES else spec
    if callable(factory):
        return f"{getattr(factory, '__module__', '?')}:{getattr(factory, '__qualname__', type(factory).__name__)}"
    return factory


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
        return factory if callable(factory) else resolve(factory, "policy")
    if ":" not in spec:
        raise ValueError(
            f"policy {spec!r} is neither a built-in ({', '.join(builtin_policies())}) nor of the form "
            "'package.module:factory'"
        )
    return resolve(spec, "policy")


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
