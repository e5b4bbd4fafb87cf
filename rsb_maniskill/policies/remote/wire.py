"""What travels between an openpi-style policy client and server: the msgpack-numpy codec, the
flat observation keys and the websocket connection (no policy logic: ``client.py`` and
``server.py`` both import it, ``vla_eval.py`` its connection).

Wire protocol (openpi ``WebsocketPolicyServer`` / ``WebsocketClientPolicy``), all binary frames
packed with msgpack + the msgpack-numpy scheme below:

1. on connect the server sends its metadata dict;
2. the client sends an observation dict, the server replies a dict holding ``"actions"`` (an
   action chunk, shape (T, D)) and, from a policy that talks, ``"text"`` (a str: the client's
   ``act`` then returns ``{"actions": chunk, "text": text}``); repeat. A text frame instead of a
   reply is the server's error (one line from ``server.py``, a traceback from openpi's), then it closes.

Batched requests (``--num-envs``: one request per step for all envs that need a chunk) carry
the same keys with a leading env dim on every array, the prompts as a list of strings and
``"env_ids"``; the reply's ``"actions"`` is (B, T, D), its ``"text"`` (if any) a list of B strings
or nils. ``server.py`` answers them with a policy's
batched form; a server that takes one observation at a time needs ``RemotePolicy(batch=False)``.

Arrays travel as ``{"__ndarray__": True, "data": raw bytes, "dtype": dtype.str, "shape": shape}``
and numpy scalars as ``{"__npgeneric__": True, "data": value, "dtype": dtype.str}`` (bytes keys),
exactly as ``openpi_client.msgpack_numpy``, so either side can be openpi's own code. Unlike openpi's,
the decoder (:func:`unpackb`, both sides) trusts nothing: only bool / int / uint / float dtypes,
shapes of at most :data:`MAX_NDIM` dims >= 0 whose bytes are exactly the data, at most
:data:`MAX_DEPTH` levels of nesting, no msgpack extension types; anything else is a one-line
:class:`WireError`. Websockets of either side refuse a message over ``max_message_mb`` before
reading it, and a server started with a token takes only clients that send it as
``Authorization: Api-Key TOKEN`` (:data:`TOKEN_ENV`).
"""
from __future__ import annotations

import inspect
import math
import reprlib
import sys
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


# ---------------------------------------------------------------- limits of a message
# Every message of either side is decoded by :func:`unpack_map`, which trusts nothing: a message can
# come from anyone who reaches the port, and a reply from whatever answers at the client's address.
MIB = 1 << 20
# A batch of camera observations at the documented sizes: 3 cameras of 320 x 240 rgb (uint8) are
# 0.69 MB a row, 44 MB for the server's 64 rows; with depth and segmentation (int16 each) 103 MB.
DEFAULT_MAX_MESSAGE_MB = 128.0  # rsb serve --max-message-mb / RemotePolicy(max_message_mb=...)
MAX_DEPTH = 32  # nested maps / lists (a request is 2-3 deep: keys, an image dict, an array's tag)
MAX_NDIM = 32  # dimensions of an array (numpy 1.x's own limit)
TOKEN_ENV = "RSB_SERVE_TOKEN"  # rsb serve's token, read by the server and by RemotePolicy when not given
TOKEN_SCHEME = "Api-Key"  # sent as ``Authorization: Api-Key TOKEN``, the header openpi's client sends its api_key in
# The array dtypes that travel (observations and actions): bool, signed / unsigned ints, floats, either
# byte order. Objects (pointers), void (structured) and the rest never become arrays from a message's bytes.
_DTYPES = {np.dtype(c).newbyteorder(o).str: np.dtype(c).newbyteorder(o)
           for c in ("?", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8", "f2", "f4", "f8") for o in "<>"}
_ARRAY_KEYS = frozenset((b"__ndarray__", b"data", b"dtype", b"shape"))
_SCALAR_KEYS = frozenset((b"__npgeneric__", b"data", b"dtype"))
_LEAVES = (type(None), bool, int, float, str, bytes)


class WireError(ValueError):
    """A message that breaks the protocol; its text is one line saying what is wrong with it."""


def max_message_bytes(mb: Any, name: str = "max_message_mb") -> int:
    """The websocket size bound (``max_size``) of ``mb`` megabytes (MiB); ValueError (one line) naming
    ``name`` unless a finite number > 0."""
    if isinstance(mb, bool) or not isinstance(mb, (int, float)) or not 0 < mb < float("inf"):
        raise ValueError(f"{name} must be a number of MB > 0 (default {DEFAULT_MAX_MESSAGE_MB:g}), got {mb!r}")
    return max(1, int(mb * MIB))


# ---------------------------------------------------------------- msgpack-numpy (openpi scheme)
def pack_array(obj: Any) -> Any:
    """msgpack ``default`` hook: numpy arrays / scalars -> tagged dicts; other objects pass through.
    Only the dtypes a receiver accepts are sent (bool, int, uint, float)."""
    if isinstance(obj, (np.ndarray, np.generic)) and obj.dtype.str not in _DTYPES:
        raise TypeError(f"an array of dtype {obj.dtype} cannot be sent: only bool, int, uint and float arrays "
                        "travel (convert it; send text as str)")
    if isinstance(obj, np.ndarray):
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
    if isinstance(obj, np.generic):
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    return obj


def packb(obj: Any) -> bytes:
    """Pack a (nested) structure holding numpy arrays."""
    return _msgpack().packb(obj, default=pack_array)


def _dtype(tag: dict, where: str) -> np.dtype:
    name = tag[b"dtype"]
    dtype = _DTYPES.get(name) if isinstance(name, str) else None
    if dtype is None:
        raise WireError(f"{where}: dtype {reprlib.repr(name)} is not allowed: only bool, int, uint and float "
                        "arrays, as numpy's dtype.str ('|u1', '<f4', ...)")
    return dtype


def _array(tag: dict, where: str) -> np.ndarray:
    """A tagged array, checked before a byte of it is read: an allowed dtype, a shape of at most
    :data:`MAX_NDIM` dims >= 0, and exactly the bytes that shape holds. A read-only view of the bytes."""
    if tag.keys() != _ARRAY_KEYS or tag[b"__ndarray__"] is not True:
        raise WireError(f"{where}: an array is a map of exactly __ndarray__ (true), data, dtype and shape")
    dtype = _dtype(tag, where)
    shape, data = tag[b"shape"], tag[b"data"]
    if not isinstance(shape, list) or len(shape) > MAX_NDIM \
            or not all(type(d) is int and d >= 0 for d in shape):  # noqa: E721  (bool is an int: refused)
        raise WireError(f"{where}: shape {reprlib.repr(shape)} is not a list of at most {MAX_NDIM} ints >= 0")
    if not isinstance(data, bytes):
        raise WireError(f"{where}: an array's data must be bytes (msgpack bin), got {type(data).__name__}")
    size = math.prod(shape) * dtype.itemsize
    if len(data) != size:
        raise WireError(f"{where}: shape {tuple(shape)} of {dtype} holds {size} bytes, the data has {len(data)}")
    try:
        return np.frombuffer(data, dtype=dtype).reshape(shape)
    except ValueError as err:  # a dim numpy cannot index (> 2**63 - 1), even with no element
        raise WireError(f"{where}: shape {reprlib.repr(shape)}: {err}") from None


def _scalar(tag: dict, where: str) -> np.generic:
    if tag.keys() != _SCALAR_KEYS or tag[b"__npgeneric__"] is not True:
        raise WireError(f"{where}: a numpy scalar is a map of exactly __npgeneric__ (true), data and dtype")
    dtype, value = _dtype(tag, where), tag[b"data"]
    kind = {"b": (bool,), "i": (int,), "u": (int,), "f": (float, int)}[dtype.kind]
    if type(value) not in kind or (dtype.kind in "iu" and not np.iinfo(dtype).min <= value <= np.iinfo(dtype).max):
        raise WireError(f"{where}: {reprlib.repr(value)} is not a value of dtype {dtype}")
    return dtype.type(value)


def _decode(node: Any, depth: int, where: str) -> Any:
    """Arrays and scalars from their tags, in place; every other value a msgpack basic type."""
    if depth > MAX_DEPTH:
        raise WireError(f"nested deeper than {MAX_DEPTH} levels (at {where})")
    if isinstance(node, dict):
        if b"__ndarray__" in node:
            return _array(node, where)
        if b"__npgeneric__" in node:
            return _scalar(node, where)
        for key, value in node.items():
            node[key] = _decode(value, depth + 1, f"{where}/{_key(key)}")
        return node
    if isinstance(node, list):
        for i, value in enumerate(node):
            node[i] = _decode(value, depth + 1, f"{where}[{i}]")
        return node
    if not isinstance(node, _LEAVES):  # a msgpack Timestamp: no ext type is part of the protocol
        raise WireError(f"{where}: a {type(node).__name__} is not part of the protocol")
    return node


def _key(key: Any) -> str:
    return key if isinstance(key, str) and len(key) <= 60 else reprlib.repr(key)


def _no_ext(code: int, data: bytes) -> Any:
    raise WireError(f"msgpack extension type {code} is not part of the protocol")


def unpackb(data: Any, what: str = "message") -> Any:
    """Inverse of :func:`packb`, for bytes from anyone: WireError (one line) for what is not a
    message of the protocol (a text frame, not msgpack, nested too deep, a dtype or shape not allowed...)."""
    if isinstance(data, str):
        raise WireError(f"a text frame: a {what} is a binary frame of msgpack")
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise WireError(f"a {what} must be bytes, got {type(data).__name__}")
    msgpack = _msgpack()
    try:
        out = msgpack.unpackb(data, raw=False, strict_map_key=True, use_list=True, ext_hook=_no_ext)
    except WireError:
        raise
    except msgpack.exceptions.StackError:
        raise WireError(f"not a {what}: nested deeper than {MAX_DEPTH} levels") from None
    except msgpack.exceptions.ExtraData:
        raise WireError(f"not one {what}: bytes follow the end of a msgpack value") from None
    except msgpack.exceptions.FormatError:
        raise WireError(f"not a {what}: not msgpack (a byte no msgpack value starts with)") from None
    except UnicodeDecodeError as err:
        raise WireError(f"a string of the {what} is not UTF-8 ({err.reason} at byte {err.start})") from None
    except RecursionError:  # msgpack's pure-Python fallback on deep nesting
        raise WireError(f"not a {what}: nested deeper than {MAX_DEPTH} levels") from None
    except (ValueError, TypeError) as err:
        raise WireError(f"not a {what}: not msgpack ({err or type(err).__name__})") from None
    return _decode(out, 1, what)


def unpack_map(data: Any, what: str = "message") -> dict:
    """A message that must be a map (a request, a reply, the server's metadata): :func:`unpackb`, then
    WireError unless it is a dict."""
    out = unpackb(data, what)
    if not isinstance(out, dict):
        raise WireError(f"a {what} must be a msgpack map (dict), got {type(out).__name__}")
    return out


def _ints(value: Any, name: str, rows: int) -> list[int]:
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind in "iu":
        value = value.tolist()
    if not isinstance(value, list) or len(value) != rows or not all(type(v) is int for v in value):  # noqa: E721
        raise WireError(f"{name!r} must be {rows} ints (one per prompt), got {_describe(value)}")
    return value


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    return f"{type(value).__name__} of length {len(value)}" if isinstance(value, (list, str)) else type(value).__name__


def read_request(data: Any, prompt_key: str = "prompt") -> dict:
    """A request as a server receives it: a map (:func:`unpack_map`) whose protocol keys have their
    types: the prompt a str (a batched request: a list of str), ``env_ids`` distinct ints >= 0 and
    ``episode_seeds`` ints, one per prompt, ``episode_seed`` an int. WireError, one line, otherwise."""
    request = unpack_map(data, "request")
    prompt = request.get(prompt_key, "")
    if isinstance(prompt, list):
        if not all(isinstance(p, str) for p in prompt):
            raise WireError(f"{prompt_key!r} of a batched request must be a list of strings")
        if "env_ids" in request:
            envs = _ints(request["env_ids"], "env_ids", len(prompt))
            if min(envs, default=0) < 0 or len(set(envs)) != len(envs):
                raise WireError(f"'env_ids' must be distinct ints >= 0, got {reprlib.repr(envs)}")
        if request.get("episode_seeds") is not None:
            _ints(request["episode_seeds"], "episode_seeds", len(prompt))
    elif not isinstance(prompt, str):
        raise WireError(f"{prompt_key!r} must be a string (a batched request: a list of strings), got "
                        f"{_describe(prompt)}")
    seed = request.get("episode_seed")
    if seed is not None and not (type(seed) is int or isinstance(seed, np.integer)):  # noqa: E721
        raise WireError(f"'episode_seed' must be an int, got {_describe(seed)}")
    return request


def error_line(text: str) -> str:
    """One line of a server's error text: itself, or a traceback's last line (the exception and its message)."""
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[-1] if len(lines) > 1 and lines[0].startswith("Traceback") else " ".join(lines)


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
class ServerUnreachable(ConnectionError):
    """Nothing accepted the connection within the connect timeout (no server there, or one still loading)."""


def open_websocket(uri: str, timeout: float, headers: dict[str, str] | None = None,
                   max_message_mb: float = DEFAULT_MAX_MESSAGE_MB, **options: Any) -> Any:
    """A blocking websocket connection to a policy server, retrying a refused connection for ``timeout`` s
    (servers still loading their weights; one line on stderr says it waits); ``options`` go to
    ``websockets.sync.client.connect``. Messages from the server over ``max_message_mb`` end the
    connection unread. ServerUnreachable at the timeout; ConnectionError (one line) when the server
    refuses the handshake (a missing or wrong token: 401 / 403) or is not a websocket server."""
    try:
        from websockets.exceptions import InvalidHandshake, InvalidStatus
        from websockets.sync.client import connect
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(INSTALL_HINT) from err
    kwargs: dict[str, Any] = {"compression": None, "max_size": max_message_bytes(max_message_mb),
                              "open_timeout": max(1.0, min(timeout, 30.0)), **options}
    if headers:
        kwargs["additional_headers"] = headers
    params = inspect.signature(connect).parameters
    if "proxy" in params:
        kwargs["proxy"] = None  # a policy server is reached directly, as with websockets < 15
    if "legacy" in params:
        kwargs["legacy"] = True  # websockets >= 17: a plain connection object, as openpi's client uses
    deadline, waiting = time.monotonic() + timeout, False
    while True:
        try:
            return connect(uri, **kwargs)
        except InvalidStatus as err:
            status = err.response.status_code
            body = error_line(bytes(err.response.body or b"").decode("utf-8", errors="replace"))
            raise ConnectionError(f"policy server {uri} refused the connection: HTTP {status} "
                                  f"{err.response.reason_phrase}" + (f": {body}" if body else "")) from None
        except InvalidHandshake as err:
            raise ConnectionError(f"{uri} is not a websocket policy server: {err}") from None
        except (ConnectionRefusedError, OSError) as err:
            if time.monotonic() >= deadline:
                raise ServerUnreachable(f"no policy server at {uri} after {timeout:.0f} s: {err}") from err
            if not waiting:
                print(f"waiting up to {timeout:.0f} s for a policy server at {uri} ...", file=sys.stderr, flush=True)
                waiting = True
            time.sleep(0.5)
