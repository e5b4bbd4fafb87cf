"""Client for policies served by a vla-eval model server: ``rsb eval remote -a protocol=vla-eval``.

vla-eval's protocol (version 1, ``vla_eval/protocol/messages.py``): WebSocket + msgpack messages
``hello``, ``episode_start``, ``observation``, ``action``, ``episode_end``, ``error``. Messages are
packed and unpacked with vla-eval's own ``pack_message`` / ``unpack_message``, so arrays and images
(PNG by default) are encoded by its codec, and the HELLO payload is its ``make_hello_payload``:

1. on connect the client says HELLO; the server answers with its name and, when it declares them,
   its action and observation specs, checked against the layout (``vla_eval_layout.check_server_spec``);
2. each episode is ``episode_start`` {"task": ...}, then ``observation`` -> ``action`` pairs, and
   ``episode_end`` before the next episode starts (and on close); an ``error`` reply raises.

Chunks: a vla-eval ``PredictModelServer`` with ``chunk_size`` k replies one action per observation
and answers the next k - 1 observations from the rest of its chunk without reading them; without a
chunk size it replies the whole (T, D) chunk. With ``chunk_size=k`` here, one ``act`` sends the
rendered observation, then k - 1 observations without images (state and instruction) at once, and
returns the k actions as one chunk, so the runner renders the cameras once per chunk, not per step
(as vla-eval's RoboTwin benchmark does with ``render_every``). A (T, D) reply is one chunk, cut to
``chunk_size`` when set.

Text: vla-eval's action payload is an open dict; a reply with a string under ``"text"`` (a server
that reports what it read, e.g. the answer it chose) makes ``act`` return ``{"actions": chunk,
"text": text}`` instead of the chunk. A chunking ``PredictModelServer`` forwards only ``actions`` of
buffered steps, so text reaches the client from servers that reply whole chunks.

Parallel envs (``--num-envs``): one connection (one vla-eval session) per env, the requests of one
step sent together so that a server with ``max_batch_size`` > 1 batches them.
"""
from __future__ import annotations

import inspect
from typing import Any, Mapping, Sequence

import numpy as np

from rsb_maniskill.batch import env_row
from rsb_maniskill.policies.interface import as_chunk
from rsb_maniskill.policies.remote.vla_eval_layout import VlaEvalLayout, check_server_spec, make_layout, vla_eval_module
from rsb_maniskill.policies.remote.wire import open_websocket

PROTOCOL = "vla-eval"  # its name in remote.PROTOCOLS, and the policy name its records carry
TASK = {"name": "RSB", "suite": "RSB"}  # the episode_start task: the policy is not told the suite or seed


class _Session:
    """One vla-eval session: a websocket, its sequence numbers and whether an episode is open."""

    def __init__(self, uri: str, connect_timeout: float, request_timeout: float | None) -> None:
        self.m = vla_eval_module("protocol.messages")
        self.uri, self.request_timeout = uri, request_timeout
        # no keepalive pings, as vla-eval's own client: a server warming up holds the GIL for long
        self.ws = open_websocket(uri, connect_timeout, ping_interval=None)
        self.seq, self.in_episode = 0, False
        self.send(self.m.MessageType.HELLO, self.m.make_hello_payload(benchmark="rsb_maniskill"))
        reply = self.recv()
        if reply.type != self.m.MessageType.HELLO:
            raise RuntimeError(f"vla-eval server {uri} answered HELLO with {reply.type.value!r}")
        self.server_info: dict[str, Any] = dict(reply.payload)

    def send(self, kind: Any, payload: dict[str, Any]) -> int:
        self.seq += 1
        self.ws.send(self.m.pack_message(self.m.Message(type=kind, payload=payload, seq=self.seq)))
        return self.seq

    def recv(self) -> Any:
        data = self.ws.recv(timeout=self.request_timeout)
        if isinstance(data, str):
            raise RuntimeError(f"vla-eval server {self.uri} sent text, not a message: {data[:200]}")
        return self.m.unpack_message(data)

    def start(self, task: Mapping[str, Any]) -> None:
        self.end()
        self.send(self.m.MessageType.EPISODE_START, {"task": dict(task)})
        self.in_episode = True

    def end(self) -> None:
        if self.in_episode:
            self.send(self.m.MessageType.EPISODE_END, {})
            self.in_episode = False

    def observe(self, observations: Sequence[dict[str, Any]]) -> None:
        for obs in observations:
            self.send(self.m.MessageType.OBSERVATION, obs)

    def replies(self, n: int) -> list[dict[str, Any]]:
        """The next ``n`` action payloads; all are read before an error is raised, so the session stays in step."""
        out, errors = [], []
        for _ in range(n):
            msg = self.recv()
            if msg.type == self.m.MessageType.ERROR:
                errors.append(msg.payload.get("error", msg.payload))
            elif msg.type != self.m.MessageType.ACTION:
                errors.append(f"unexpected {msg.type.value!r} message")
            else:
                out.append(msg.payload)
        if errors:
            raise RuntimeError(f"vla-eval server {self.uri}: {errors[0]}")
        return out

    def close(self) -> None:
        try:
            self.end()
        finally:
            self.ws.close()


class VlaEvalPolicy:
    """A :class:`~rsb_maniskill.policies.interface.Policy` (and its batched form) whose actions come
    from a vla-eval model server.

    Args:
        host: server host, or a full ``ws://`` URI.
        port: server port (None when ``host`` is a URI that holds it).
        preset: ``lerobot`` or ``robotwin``, the observation / action layout (``vla_eval_layout.PRESETS``).
        cameras, state_key, gripper, joints: layout options replacing the preset's (``state_key=none``: no state).
        chunk_size: actions executed per observation the server reads: a chunking server's ``chunk_size``
            (the LeRobot bridge: the policy's ``n_action_steps``); None: one per observation.
        image_format: ``png`` (vla-eval's default), ``jpeg`` or ``raw``: how images travel.
        connect_timeout: seconds to keep retrying a refused connection.
        request_timeout: seconds to wait for a reply.
        name: label of the records' ``policy`` field when no ``--name`` is given.
    """

    def __init__(self, host: str = "127.0.0.1", port: int | None = 8000, preset: str = "lerobot",
                 cameras: str | None = None, state_key: str | None = None, gripper: str | None = None,
                 joints: str | None = None, chunk_size: int | None = None, image_format: str = "png",
                 connect_timeout: float = 60.0, request_timeout: float | None = 300.0,
                 name: str = PROTOCOL) -> None:
        self.layout: VlaEvalLayout = make_layout(preset, cameras=cameras, state_key=state_key, gripper=gripper,
                                                 joints=joints)
        if chunk_size is not None and (not isinstance(chunk_size, int) or chunk_size < 1):
            raise ValueError(f"chunk_size must be a positive int (the server's chunk size), got {chunk_size!r}")
        if image_format not in ("png", "jpeg", "raw"):
            raise ValueError(f"image_format must be png, jpeg or raw, got {image_format!r}")
        vla_eval_module("protocol.numpy_codec").set_image_format(image_format)  # vla-eval keeps it process-wide
        self.uri = host if host.startswith(("ws://", "wss://")) else f"ws://{host}"
        if port is not None and not host.startswith(("ws://", "wss://")):
            self.uri += f":{port}"
        self.chunk_size, self.name = chunk_size, name
        self.connect_timeout, self.request_timeout = connect_timeout, request_timeout
        self.sessions = [self._session()]
        self.server_info = self.sessions[0].server_info
        check_server_spec(self.server_info, self.layout)
        self.instructions: list[str] = [""]

    def _session(self) -> _Session:
        return _Session(self.uri, self.connect_timeout, self.request_timeout)

    # ------------------------------------------------------------ single env
    def reset(self, instruction: str, obs: dict) -> None:
        self.reset_batch([instruction], None)

    def act(self, obs: dict) -> Any:
        return self._chunks([obs], [0])[0]

    # ------------------------------------------------------------ batched form (parallel envs)
    def reset_batch(self, instructions: Sequence[str], obs: Any) -> None:
        self.instructions = list(instructions)
        while len(self.sessions) < len(self.instructions):
            self.sessions.append(self._session())
        for text, session in zip(self.instructions, self.sessions):
            session.start({**TASK, "instruction": text})

    def act_batch(self, obs: dict, envs: Any) -> list[Any]:
        envs = [int(e) for e in envs]
        return self._chunks([env_row(obs, k) for k in range(len(envs))], envs)

    def _chunks(self, observations: list[dict], envs: list[int]) -> list[Any]:
        """Send each env's observation, then the steps' observations a chunking server reads from its
        buffer; every request of a round is sent before any reply is read."""
        sent = [self.layout.observation(o, self.instructions[e]) for o, e in zip(observations, envs)]
        for payload, e in zip(sent, envs):
            self.sessions[e].observe([payload])
        first = [self.sessions[e].replies(1)[0] for e in envs]
        extra = [0] * len(envs)
        for k, (reply, e) in enumerate(zip(first, envs)):
            if np.ndim(reply.get("actions")) == 1 and (self.chunk_size or 1) > 1:
                extra[k] = self.chunk_size - 1
                light = {key: v for key, v in sent[k].items() if key != "images"}
                self.sessions[e].observe([light] * extra[k])
        return [self._chunk([reply, *self.sessions[e].replies(n)], sent[k])
                for k, (reply, e, n) in enumerate(zip(first, envs, extra))]

    def _chunk(self, replies: list[dict], sent: dict) -> Any:
        if any("actions" not in r for r in replies):
            keys = sorted({str(k) for r in replies for k in r})
            raise RuntimeError(f"vla-eval server {self.uri} replied without 'actions' (keys: {keys})")
        if len(replies) == 1 and np.ndim(replies[0]["actions"]) == 2:
            wire = np.asarray(replies[0]["actions"])[: self.chunk_size]
        else:
            wire = np.stack([np.asarray(r["actions"]).reshape(-1) for r in replies])
        state = sent.get(self.layout.state_key) if self.layout.state_key else None
        chunk = as_chunk(self.layout.env_actions(wire, state))
        text = next((r["text"] for r in replies if isinstance(r.get("text"), str)), None)
        return chunk if text is None else {"actions": chunk, "text": text}

    def close(self) -> None:
        for session in self.sessions:
            session.close()

    def __enter__(self) -> "VlaEvalPolicy":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def probe_server(policy_kwargs: Mapping[str, Any], obs_mode: str) -> None:
    """Before any env is built: the options, the obs mode they need, and the server's HELLO (reachable,
    and a spec the layout meets). Raises ValueError / ConnectionError in one line."""
    kwargs = {k: v for k, v in policy_kwargs.items() if k != "protocol"}
    unknown = set(kwargs) - set(inspect.signature(VlaEvalPolicy).parameters)
    if unknown:
        raise ValueError(f"-a {', '.join(sorted(unknown))}: not an option of protocol=vla-eval "
                         f"(options: {', '.join(inspect.signature(VlaEvalPolicy).parameters)})")
    if "rgb" not in obs_mode and obs_mode != "state_dict":
        raise ValueError(f"protocol=vla-eval sends camera images (an rgb obs mode) or the state alone (state_dict), "
                         f"not obs mode {obs_mode!r}")
    VlaEvalPolicy(**kwargs).close()
