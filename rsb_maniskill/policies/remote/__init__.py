"""Policies over the network: one table of wire protocols, picked by the ``remote`` policy's
``protocol`` argument (``-a protocol=NAME``).

- ``openpi`` (default): openpi's websocket protocol. The client policy (``client.py``), a server for
  any RSB policy (``server.py``, ``python -m rsb_maniskill.policies.remote.server``), the wire
  codec both use (``wire.py``) and the ``openpi-aloha`` preset (``openpi.py``). Needs the ``eval``
  extra (websockets, msgpack).
- ``vla-eval``: the protocol of allenai's vla-evaluation-harness model servers (``vla_eval.py``, its
  observation / action layout in ``vla_eval_layout.py``). Needs the ``vla_eval`` extra.

A protocol is a client module and one row of :data:`PROTOCOLS`: the client's factory and the check
that runs before any env is built. Both are named, not imported: naming the ``remote`` policy
imports no client. A new protocol is one file: its module calls :func:`register_protocol` (from a
plugin, ``plugins.py``), or is named directly, ``-a protocol=package.module:Client`` (its optional
``check_remote_args(policy_kwargs, obs_mode)`` beside it is the check).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from rsb_maniskill.resolve import resolve


@dataclass(frozen=True)
class Protocol:
    client: str  # "module:factory" of the client policy, called with the policy's arguments
    check: str  # "module:function" (policy_kwargs, obs_mode) -> None, ValueError in one line


PROTOCOLS: dict[str, Protocol] = {
    "openpi": Protocol("rsb_maniskill.policies.remote.client:RemotePolicy",
                       "rsb_maniskill.policies.remote.client:check_remote_args"),
    "vla-eval": Protocol("rsb_maniskill.policies.remote.vla_eval:VlaEvalPolicy",
                         "rsb_maniskill.policies.remote.vla_eval:probe_server"),
}
DEFAULT_PROTOCOL = "openpi"
_NO_CHECK = "rsb_maniskill.policies.remote:no_check"


def register_protocol(name: str, client: str, check: str | None = None) -> None:
    """Add a protocol row: ``client`` and ``check`` as :class:`Protocol` takes them (no check: none)."""
    if ":" in name:
        raise ValueError(f"protocol names cannot contain ':', got {name!r}")
    if name in PROTOCOLS:  # a plugin cannot replace a built-in (or another plugin's) protocol
        raise ValueError(f"protocol name {name!r} is taken; register the protocol under another name")
    PROTOCOLS[name] = Protocol(client, check or _NO_CHECK)


def get_protocol(name: str) -> Protocol:
    """The row of ``name``, or the row a ``"module:Client"`` name makes; ValueError naming the known ones."""
    if name in PROTOCOLS:
        return PROTOCOLS[name]
    if ":" in name:
        module = name.partition(":")[0]
        check = f"{module}:check_remote_args"
        try:
            resolve(check, "protocol check")
        except (ImportError, AttributeError, TypeError, ValueError):
            check = _NO_CHECK
        return Protocol(name, check)
    raise ValueError(f"-a protocol={name}: unknown protocol; known: {', '.join(PROTOCOLS)} "
                     "(or name a client as package.module:Client)")


def no_check(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """The check of a protocol that has none."""


def remote_policy(protocol: str = DEFAULT_PROTOCOL, **kwargs: Any) -> Any:
    """The ``remote`` policy: the client of ``protocol`` (``RemotePolicy``, ``VlaEvalPolicy``, ...)."""
    return resolve(get_protocol(protocol).client, "protocol client")(**kwargs)


def check_remote_args(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """Before any env is built: the ``remote`` policy's arguments for its protocol (ValueError, one line)."""
    row = get_protocol(policy_kwargs.get("protocol", DEFAULT_PROTOCOL))
    resolve(row.check, "protocol check")(policy_kwargs, obs_mode)
