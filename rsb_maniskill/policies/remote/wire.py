"""What travels between an openpi-style policy client and server: the msgpack-numpy codec, the
flat observation keys and the websocket connection (no policy logic: ``client.py`` and
``server.py`` both import it, ``vla_eval.py`` its connection).

Wire protocol (openpi ``WebsocketPolicyServer`` / ``WebsocketClientPolicy``), all binary frames
packed with msgpack + the msgpack-numpy scheme below:

1. on connect the server sends its metadata dict;
2. the client sends an observation dict, the server replies a dict holding ``"actions"`` (an
   action chunk, shape (T, D)) and, from a policy that talks, ``"text"`` (a str: the client's
   ``act`` then returns ``{"actions": chunk, "text": text}``); repeat. A text frame instead of a
   reply is a server traceback.

Batched requests (``--num-envs``: one request per step for all envs that need a chunk) carry
the same keys with a leading env dim on every array, the prompts as a list of strings and
``"env_ids"``; the reply's ``"actions"`` is (B, T, D), its ``"text"`` (if any) a list of B strings
or nils. ``server.py`` answers them with a policy's
batched form; a server that takes one observation at a time needs ``RemotePolicy(batch=False)``.

Arrays travel as ``{"__ndarray__": True, "data": raw bytes, "dtype": dtype.str, "shape": shape}``
and numpy scalars as ``{"__npgeneric__": True, "data": value, "dtype": dtype.str}`` (bytes keys),
exactly as ``openpi_client.msgpack_numpy``, so either side can be openpi's own code.
"""
from __future__ import annotations

import inspect
import time
from typing import Any, Mapping

import numpy as np

INSTALL_HINT = "the remote policy client needs `pip install websockets msgpack` (extra: rsb_maniskill[eval])"


def _msgpack():
    try:
        import msgpack
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(INSTALL_HINT) from err
    return msgpack


# ---------------------------------------------------------------- msgpack-numpy (openpi scheme)
def pack_array(obj: Any) -> Any:
    """msgpack ``default`` hook: numpy arrays / scalars -> tagged dicts; other objects pass through."""
    if isinstance(obj, (np.ndarray, np.generic)) and obj.dtype.kind in ("V", "O", "c"):
        raise ValueError(f"unsupported dtype for msgpack-numpy: {obj.dtype}")
    if isinstance(obj, np.ndarray):
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
    if isinstance(obj, np.generic):
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    return obj


def unpack_array(obj: dict) -> Any:
    """msgpack ``object_hook``: tagged dicts -> numpy arrays (read-only views) / scalars."""
    if b"__ndarray__" in obj:
        return np.ndarray(buffer=obj[b"data"], dtype=np.dtype(obj[b"dtype"]), shape=obj[b"shape"])
    if b"__npgeneric__" in obj:
        return np.dtype(obj[b"dtype"]).type(obj[b"data"])
    return obj


def packb(obj: Any) -> bytes:
    """Pack a (nested) structure holding numpy arrays."""
    return _msgpack().packb(obj, default=pack_array)


def unpackb(data: bytes) -> Any:
    """Inverse of :func:`packb`."""
    return _msgpack().unpackb(data, object_hook=unpack_array)


# ---------------------------------------------------------------- observation keys
def _to_numpy(x: Any) -> Any:
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # torch tensor, without importing torch
        return x.detach().cpu().numpy()
    if isinstance(x, (np.ndarray, np.generic, str, bytes, bool, int, float)) or x is None:
        return x
    return np.asarray(x)


def flatten_obs(obs: Mapping[str, Any], prefix: str = "observation") -> dict[str, Any]:
    """Nested obs -> flat dict with "/"-joined keys under ``prefix``.

    ``{"agent": {"qpos": a}, "sensor_data": {"head": {"rgb": b}}}`` ->
    ``{"observation/agent/qpos": a, "observation/sensor_data/head/rgb": b}``.
    """
    out: dict[str, Any] = {}
    if not isinstance(obs, Mapping):  # a flat "state" observation: one array under the prefix
        return {prefix or "observation": _to_numpy(obs)}

    def walk(node: Mapping[str, Any], path: str) -> None:
        for key, value in node.items():
            p = f"{path}/{key}" if path else str(key)
            if isinstance(value, Mapping):
                walk(value, p)
            else:
                out[p] = _to_numpy(value)

    walk(obs, prefix)
    return out


def unflatten_obs(flat: Mapping[str, Any], prefix: str = "observation") -> dict[str, Any]:
    """Inverse of :func:`flatten_obs`; keys outside ``prefix`` stay at the top level as they are."""
    out: dict[str, Any] = {}
    head = f"{prefix}/" if prefix else ""
    for key, value in flat.items():
        if head and not key.startswith(head):
            out[key] = value
            continue
        node = out
        *parents, leaf = key[len(head):].split("/")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


# ---------------------------------------------------------------- connection
def open_websocket(uri: str, timeout: float, headers: dict[str, str] | None = None, **options: Any) -> Any:
    """A blocking websocket connection to a policy server, retrying a refused connection for ``timeout`` s
    (servers still loading their weights); ``options`` go to ``websockets.sync.client.connect``."""
    try:
        from websockets.sync.client import connect
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(INSTALL_HINT) from err
    kwargs: dict[str, Any] = {"compression": None, "max_size": None, "open_timeout": max(1.0, min(timeout, 30.0)),
                              **options}
    if headers:
        kwargs["additional_headers"] = headers
    params = inspect.signature(connect).parameters
    if "proxy" in params:
        kwargs["proxy"] = None  # a policy server is reached directly, as with websockets < 15
    if "legacy" in params:
        kwargs["legacy"] = True  # websockets >= 17: a plain connection object, as openpi's client uses
    deadline = time.monotonic() + timeout
    while True:
        try:
            return connect(uri, **kwargs)
        except (ConnectionRefusedError, OSError) as err:
            if time.monotonic() >= deadline:
                raise ConnectionError(f"no policy server at {uri} after {timeout:.0f} s: {err}") from err
            time.sleep(0.5)
