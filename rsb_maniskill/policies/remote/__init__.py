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
imports no client.
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


def get_protocol(name: str) -> Protocol:
    """The row of ``name``; ValueError naming the known protocols."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ValueError(f"-a protocol={name}: unknown protocol; known: {', '.join(PROTOCOLS)}") from None


def remote_policy(protocol: str = DEFAULT_PROTOCOL, **kwargs: Any) -> Any:
    """The ``remote`` policy: the client of ``protocol`` (``RemotePolicy``, ``VlaEvalPolicy``, ...)."""
    return resolve(get_protocol(protocol).client, "protocol client")(**kwargs)


def check_remote_args(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """Before any env is built: the ``remote`` policy's arguments for its protocol (ValueError, one line)."""
    row = get_protocol(policy_kwargs.get("protocol", DEFAULT_PROTOCOL))
    resolve(row.check, "protocol check")(policy_kwargs, obs_mode)
