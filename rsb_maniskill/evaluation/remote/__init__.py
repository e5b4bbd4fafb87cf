"""Policies over the network. Two protocols, picked by the ``remote`` policy's ``protocol`` argument:

- ``openpi`` (default): openpi's websocket protocol. The client policy (``client.py``), a server for
  any RSB policy (``server.py``, ``python -m rsb_maniskill.evaluation.remote.server``), the wire
  codec both use (``wire.py``) and the ``openpi-aloha`` preset (``openpi.py``). Needs the ``eval``
  extra (websockets, msgpack).
- ``vla-eval``: the protocol of allenai's vla-evaluation-harness model servers (``vla_eval.py``, its
  observation / action layout in ``vla_eval_layout.py``). Needs the ``vla_eval`` extra.

Imported on first use: naming the ``remote`` policy imports neither.
"""
from __future__ import annotations

from typing import Any, Mapping

PROTOCOLS = ("openpi", "vla-eval")


def remote_policy(protocol: str = "openpi", **kwargs: Any) -> Any:
    """The ``remote`` policy: an openpi client (``RemotePolicy``) or a vla-eval one (``VlaEvalPolicy``)."""
    if protocol == "openpi":
        from rsb_maniskill.evaluation.remote.client import RemotePolicy

        return RemotePolicy(**kwargs)
    if protocol == "vla-eval":
        from rsb_maniskill.evaluation.remote.vla_eval import VlaEvalPolicy

        return VlaEvalPolicy(**kwargs)
    raise ValueError(f"unknown protocol {protocol!r}; known: {', '.join(PROTOCOLS)}")


def check_remote_args(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """Before any env is built: the ``remote`` policy's arguments for its protocol (ValueError, one line)."""
    protocol = policy_kwargs.get("protocol", "openpi")
    if protocol == "openpi":
        from rsb_maniskill.evaluation.remote.client import check_remote_args as check_openpi

        check_openpi(policy_kwargs, obs_mode)
    elif protocol == "vla-eval":
        from rsb_maniskill.evaluation.remote.vla_eval import probe_server

        probe_server(policy_kwargs, obs_mode)
    else:
        raise ValueError(f"-a protocol={protocol}: unknown protocol; known: {', '.join(PROTOCOLS)}")
