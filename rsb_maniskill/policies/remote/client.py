"""Client for policies served by an openpi-style websocket server (``RemotePolicy``), and
``RemoteBackbone`` for a backbone behind one.

The wire protocol (messages, batched requests, the msgpack-numpy codec) is ``wire.py``'s; this
module holds the policy side of it: what a request carries and how a reply becomes an action chunk.
"""
from __future__ import annotations

import inspect
import os
from typing import Any, Callable, Mapping

import numpy as np

from rsb_maniskill.policies.interface import as_chunk, join_outputs
from rsb_maniskill.policies.remote.wire import (
    DEFAULT_MAX_MESSAGE_MB,
    MIB,
    TOKEN_ENV,
    TOKEN_SCHEME,
    ServerUnreachable,
    WireError,
    error_line,
    flatten_obs,
    open_websocket,
    packb,
    unpack_map,
)


def _row(obs: Any, i: int) -> Any:
    if isinstance(obs, Mapping):
        return {k: _row(v, i) for k, v in obs.items()}
    return np.asarray(obs)[i]


def _text(value: Any, uri: str) -> str | None:
    """A reply's ``text`` (msgpack may hand back bytes)."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    raise RuntimeError(f"policy server {uri} replied 'text' of type {type(value).__name__}; expected a str")


# ---------------------------------------------------------------- client
def check_remote_args(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """Before any env is built (``rsb eval remote``, openpi's protocol): the options, the preset's
    arguments and the obs mode they need (``openpi.py``), and the server: reachable, and sending its
    metadata, within ``connect_timeout`` (default 60 s). ValueError / ConnectionError, one line."""
    from rsb_maniskill.policies.remote.openpi import check_preset_args

    kwargs = {k: v for k, v in policy_kwargs.items() if k != "protocol"}
    options = [name for name in inspect.signature(RemotePolicy).parameters if name != "obs_transform"]
    unknown = sorted(set(kwargs) - set(options))
    if unknown:
        raise ValueError(f"-a {', '.join(unknown)}: not an option of the remote policy (openpi protocol; options: "
                         f"{', '.join(options)})")
    check_preset_args(kwargs, obs_mode)
    try:
        RemotePolicy(**kwargs).close()
    except ServerUnreachable as err:
        raise ConnectionError(f"{err}; start the policy server, or fix -a host / -a port (-a connect_timeout=S "
                              "waits longer for one still loading)") from None


class RemotePolicy:
    """A :class:`~rsb_maniskill.policies.interface.Policy` whose actions come from a websocket server.

    Each ``act`` sends ``flatten_obs(obs) | {"prompt": instruction}`` (or ``obs_transform(obs,
    instruction)`` when given, to match a server that expects other keys) and returns the reply's
    ``"actions"`` as a (T, D) array, cut to ``action_horizon`` steps when set, with the reply's
    ``"text"`` as ``{"actions": chunk, "text": text}`` when the server sends one.

    Args:
        host: server host, or a full ``ws://`` / ``wss://`` URI.
        port: server port (None when ``host`` is a URI that holds it).
        token: the server's token (``rsb serve --token``; default ``$RSB_SERVE_TOKEN``), sent as
            ``Authorization: Api-Key TOKEN``, the header openpi's client sends its ``api_key`` in.
        action_horizon: execute only the first k actions of each chunk before asking again.
        mark_episode_start: add ``"episode_start": True`` to the first request of each episode so
            that ``server.py``'s server resets the wrapped policy, with the episode's seed
            (``"episode_seed"``; batched: ``"episode_seeds"``) when the runner gave one; off by
            default because other servers do not expect the keys.
        connect_timeout: seconds to keep retrying a refused connection (openpi's client waits forever),
            and to wait for the server's metadata once connected: ConnectionError, one line, after it.
        max_message_mb: a reply over this many MB (MiB) ends the connection unread (``wire.py``).
        preset: ``"openpi-aloha"``: send openpi's Aloha keys and layout and read the reply as Aloha-layout
            actions (``openpi.py``); then ``image_size`` (default 224) sets the image size and
            ``action_horizon`` defaults to 10.
        batch: with parallel envs, one batched request per step (``wire.py``); False: one per env
            (always with a preset: openpi's servers take one observation per request).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int | None = 8000,
        token: str | None = None,
        prompt_key: str = "prompt",
        obs_prefix: str = "observation",
        obs_transform: Callable[[dict, str], dict] | None = None,
        action_horizon: int | None = None,
        mark_episode_start: bool = False,
        connect_timeout: float = 60.0,
        request_timeout: float | None = 300.0,
        name: str = "remote",
        preset: str | None = None,
        image_size: int | list[int] | None = None,
        batch: bool = True,
        max_message_mb: float = DEFAULT_MAX_MESSAGE_MB,
    ) -> None:
        self.preset = None
        if preset is not None:
            from rsb_maniskill.policies.remote.openpi import make_preset

            if obs_transform is not None:
                raise ValueError("give RemotePolicy either a preset or an obs_transform, not both")
            self.preset = make_preset(preset, **({} if image_size is None else {"image_size": image_size}))
            obs_transform = self.preset.request
            action_horizon = action_horizon or self.preset.action_horizon
        elif image_size is not None:
            raise ValueError("image_size applies to a preset: add preset='openpi-aloha'")
        self.uri = host if host.startswith(("ws://", "wss://")) else f"ws://{host}"
        if port is not None and not host.startswith(("ws://", "wss://")):
            self.uri += f":{port}"
        self.token = token if token is not None else os.environ.get(TOKEN_ENV) or None
        self.max_message_mb = max_message_mb
        self._sent = 0  # bytes of the last request (named when the server refuses it as too big)
        self.prompt_key = prompt_key
        self.obs_prefix = obs_prefix
        self.obs_transform = obs_transform
        self.action_horizon = action_horizon
        self.mark_episode_start = mark_episode_start
        self.request_timeout = request_timeout
        self.name = name
        self.instruction = ""
        self._episode_start = False
        self._seeds: list[int] | None = None  # of the episodes starting (the runner's seed= / seeds=)
        # openpi's Aloha policies take one observation per request: a preset sends one per env
        self.batch = batch and self.preset is None
        self.instructions: list[str] = []  # of the batched form
        self._ws, self.server_metadata = self._connect(connect_timeout)

    def _connect(self, timeout: float) -> tuple[Any, dict]:
        """Connect and read the server's metadata, each within ``timeout`` s."""
        headers = {"Authorization": f"{TOKEN_SCHEME} {self.token}"} if self.token else None
        ws = open_websocket(self.uri, timeout, headers, max_message_mb=self.max_message_mb)
        try:
            metadata = self._recv(ws, timeout, "metadata")
        except TimeoutError:
            ws.close()
            raise ConnectionError(f"{self.uri} accepted the connection but sent no metadata within {timeout:.0f} s: "
                                  "not an openpi policy server? (a vla-eval one: -a protocol=vla-eval)") from None
        except RuntimeError as err:
            ws.close()
            raise ConnectionError(str(err)) from None
        return ws, metadata

    def _recv(self, ws: Any, timeout: float | None = None, what: str = "reply") -> dict:
        """The server's next message, decoded as the server decodes ours (``wire.unpack_map``); its
        error or its closing the connection: RuntimeError, one line (a traceback in ``.detail``)."""
        from websockets.exceptions import ConnectionClosed

        try:
            msg = ws.recv(timeout=self.request_timeout if timeout is None else timeout)
        except ConnectionClosed as err:
            raise RuntimeError(self._closed(err)) from None
        if isinstance(msg, str):  # the server's error, then it closes: a line (server.py) or a traceback (openpi)
            err = RuntimeError(f"policy server {self.uri}: {error_line(msg)}")
            err.detail = msg  # type: ignore[attr-defined]  (rsb --debug prints it)
            raise err
        try:
            return unpack_map(msg, what)
        except WireError as err:
            raise RuntimeError(f"policy server {self.uri} sent a {what} this client refuses: {err}") from None

    def _closed(self, err: Any) -> str:
        """One line for a connection the server (or this client's size bound) ended."""
        sent, rcvd = getattr(err, "sent", None), getattr(err, "rcvd", None)
        server_first = rcvd is not None and (sent is None or bool(getattr(err, "rcvd_then_sent", False)))
        if sent is not None and sent.code == 1009 and not server_first:  # a reply over this client's bound
            return (f"policy server {self.uri} sent a message over this client's limit of {self.max_message_mb:g} MB "
                    f"({sent.reason}); raise it with -a max_message_mb=MB")
        if rcvd is not None and rcvd.code == 1009 and server_first:
            return (f"policy server {self.uri} refused a request of {self._sent / MIB:.1f} MB as too big "
                    f"({rcvd.reason}); start it with a larger --max-message-mb")
        if rcvd is not None:
            return f"policy server {self.uri} closed the connection (code {rcvd.code}{': ' if rcvd.reason else ''}" \
                   f"{rcvd.reason})"
        return f"policy server {self.uri} closed the connection without a word ({err}): did it stop?"

    def infer(self, payload: dict) -> dict:
        """One raw request/response round trip (openpi's ``infer``)."""
        from websockets.exceptions import ConnectionClosed

        message = packb(payload)
        self._sent = len(message)
        try:
            self._ws.send(message)
        except ConnectionClosed as err:
            raise RuntimeError(self._closed(err)) from None
        return self._recv(self._ws)

    def reset(self, instruction: str, obs: dict, seed: int | None = None) -> None:
        self.instruction = instruction
        self._episode_start = True
        self._seeds = None if seed is None else [int(seed)]

    def act(self, obs: dict) -> Any:
        if self.obs_transform is not None:
            payload = dict(self.obs_transform(obs, self.instruction))
        else:
            payload = flatten_obs(obs, self.obs_prefix)
            payload[self.prompt_key] = self.instruction
        if self.mark_episode_start and self._episode_start:
            payload["episode_start"] = True
            if self._seeds is not None:
                payload["episode_seed"] = self._seeds[0]
        self._episode_start = False
        reply = self.infer(payload)
        if "actions" not in reply:
            raise RuntimeError(f"policy server {self.uri} reply has no 'actions' (keys: {sorted(map(str, reply))})")
        chunk = as_chunk(np.array(reply["actions"]))
        if self.preset is not None:
            chunk = self.preset.env_actions(chunk)
        chunk = chunk[: self.action_horizon] if self.action_horizon else chunk
        text = _text(reply.get("text"), self.uri)
        return chunk if text is None else {"actions": chunk, "text": text}

    # ------------------------------------------------------------ batched form (parallel envs)
    def reset_batch(self, instructions: Any, obs: dict, seeds: Any = None) -> None:
        self.instructions = list(instructions)
        self._episode_start = True
        self._seeds = None if seeds is None else [int(s) for s in seeds]

    def act_batch(self, obs: dict, envs: Any) -> Any:
        """Chunks for ``envs``: one batched request, or (``batch=False``) one request per env."""
        envs = [int(e) for e in envs]
        if not self.batch:
            outs = []
            for k, e in enumerate(envs):
                self.instruction = self.instructions[e]
                outs.append(self.act(_row(obs, k)))
            return join_outputs(outs)
        prompts = [self.instructions[e] for e in envs]
        if self.obs_transform is not None:
            payload = dict(self.obs_transform(obs, prompts))
        else:
            payload = flatten_obs(obs, self.obs_prefix)
            payload[self.prompt_key] = prompts
        payload["env_ids"] = np.asarray(envs, dtype=np.int64)
        if self.mark_episode_start and self._episode_start:
            payload["episode_start"] = True
            if self._seeds is not None:
                payload["episode_seeds"] = np.asarray([self._seeds[e] for e in envs], dtype=np.int64)
        self._episode_start = False
        reply = self.infer(payload)
        actions = np.asarray(reply.get("actions")) if "actions" in reply else None
        if actions is None or actions.ndim != 3 or actions.shape[0] != len(envs):
            got = "no 'actions'" if actions is None else f"actions of shape {actions.shape}"
            raise RuntimeError(f"policy server {self.uri} replied {got} to a batched request for {len(envs)} envs; "
                               "a server that takes one observation at a time needs RemotePolicy(batch=False) "
                               "(-a batch=false)")
        chunks = [as_chunk(c)[: self.action_horizon] if self.action_horizon else as_chunk(c) for c in actions]
        texts = reply.get("text")
        if texts is None:
            return chunks
        if isinstance(texts, (str, bytes)) or len(texts) != len(envs):
            raise RuntimeError(f"policy server {self.uri} replied 'text' that is not a list of {len(envs)} texts")
        return {"actions": chunks, "text": [_text(t, self.uri) for t in texts]}

    def close(self) -> None:
        self._ws.close()

    def __enter__(self) -> "RemotePolicy":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RemoteBackbone:
    """A backbone (``rsb backbone remote``) behind a websocket server of this protocol.

    Each ``answer`` sends ``{"prompt": instruction, "images": {camera: (H, W, 3) uint8}}`` (images
    only with ``rsb backbone --images``) and returns the reply's ``"text"``; ``server.py`` serves
    any object with ``answer(instruction, images)`` that way. Arguments as :class:`RemotePolicy`.
    """

    def __init__(self, host: str = "127.0.0.1", port: int | None = 8000, token: str | None = None,
                 prompt_key: str = "prompt", connect_timeout: float = 60.0, request_timeout: float | None = 300.0,
                 name: str = "remote", max_message_mb: float = DEFAULT_MAX_MESSAGE_MB) -> None:
        self.client = RemotePolicy(host, port, token=token, prompt_key=prompt_key,
                                   connect_timeout=connect_timeout, request_timeout=request_timeout, name=name,
                                   max_message_mb=max_message_mb)
        self.name = name

    def answer(self, instruction: str, images: Mapping[str, np.ndarray]) -> str:
        payload: dict[str, Any] = {self.client.prompt_key: instruction}
        if images:
            payload["images"] = {k: np.ascontiguousarray(v) for k, v in images.items()}
        reply = self.client.infer(payload)
        text = _text(reply.get("text"), self.client.uri)
        if text is None:
            raise RuntimeError(f"backbone server {self.client.uri} reply has no 'text' "
                               f"(keys: {sorted(map(str, reply))})")
        return text

    def close(self) -> None:
        self.client.close()
